"""A small client of ``drivebus serve``: what the one-shot commands use when a service owns
the machine (the line has one owner), and a script may use too.

Synchronous, standard library only (``urllib``): each call is one request. A problem
reply (RFC 9457) becomes the typed error it names (``StateError``, ``LimitViolation``,
...); a service that cannot be reached is ``ServiceUnreachable``.
"""

from __future__ import annotations

import json
import os
import time
import urllib.error
import urllib.request
from typing import Any

from drivebus import errors, runtime
from drivebus.errors import DrivebusError, LeaseHeld, ServiceUnreachable

__all__ = ["ServiceClient", "find_service"]

_POLL = 0.05
"""Seconds between two looks at a running motion."""


def find_service(config: str | os.PathLike[str]) -> str | None:
    """The URL of the running ``drivebus serve`` of machine file ``config``, if one runs."""
    found = runtime.lookup("serve", os.path.realpath(config))
    return found[0] if found else None


class ServiceClient:
    """Requests to one ``drivebus serve`` at ``url`` (``http://127.0.0.1:8000``)."""

    def __init__(self, url: str, *, token: str | None = None, client: str = "drivebus-cli",
                 timeout: float = 10.0) -> None:
        self.url = url.rstrip("/")
        self.token = token
        self.client = client
        self.timeout = timeout

    def request(self, method: str, path: str, body: object = None) -> Any:
        """One request; the decoded JSON reply, or the typed error of a problem reply."""
        return json.loads(self._send(method, path, body) or "null")

    def text(self, path: str) -> str:
        """``GET /api/PATH`` of a reply that is not JSON (a recording's JSON lines, its
        report); the typed error of a problem reply."""
        return self._send("GET", path, None)

    def _send(self, method: str, path: str, body: object) -> str:
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(f"{self.url}/api{path}", data=data, method=method)
        req.add_header("Accept", "application/json")
        if data is not None:
            req.add_header("Content-Type", "application/json")
        if self.token:
            req.add_header("Authorization", f"Bearer {self.token}")
        else:
            req.add_header("X-Drivebus-Client", self.client)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as reply:
                text: str = reply.read().decode()
        except urllib.error.HTTPError as exc:
            raise self._problem(exc) from None
        except (urllib.error.URLError, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            raise ServiceUnreachable(f"the drivebus service at {self.url} cannot be reached: "
                                     f"{reason}") from None
        return text

    def _problem(self, exc: urllib.error.HTTPError) -> DrivebusError:
        try:
            problem = json.loads(exc.read().decode() or "{}")
        except ValueError:
            problem = {}
        name = str(problem.get("error") or problem.get("title") or "")
        detail = str(problem.get("detail") or exc.reason)
        where = f" (from the drivebus service at {self.url})"
        if name == "LeaseHeld":
            return LeaseHeld(detail + where, holder=str(problem.get("holder", "")))
        kind = getattr(errors, name, None)
        if isinstance(kind, type) and issubclass(kind, DrivebusError):
            try:
                return kind(detail + where)
            except TypeError:  # an error type whose constructor wants more than a message
                pass
        return self.refused(exc.code, name or str(exc.reason), detail)

    def refused(self, status: int, name: str, detail: str) -> DrivebusError:
        """The error of a problem reply no drivebus error names (401 without a token or
        with an unknown one, 403 beyond the token's scope, ...); a front end's client says
        there what its user does about it."""
        return DrivebusError(f"HTTP {status} {name}: {detail} (from the drivebus service at "
                             f"{self.url})")

    # -- reading ------------------------------------------------------------------------------

    def machine(self) -> dict[str, Any]:
        """``GET /api/machine``."""
        result: dict[str, Any] = self.request("GET", "/machine")
        return result

    def axis(self, name: str) -> dict[str, Any]:
        """``GET /api/axes/NAME``: the axis as plain data."""
        result: dict[str, Any] = self.request("GET", f"/axes/{name}")
        return result

    # -- commands ------------------------------------------------------------------------------

    def start(self, path: str, body: object = None) -> dict[str, Any]:
        """Start a motion (``POST``); its record (``id``, ``state``)."""
        result: dict[str, Any] = self.request("POST", path, body if body is not None else {})
        return result

    def wait(self, motion_id: str) -> dict[str, Any]:
        """The motion's record once it is no longer running."""
        while True:
            record: dict[str, Any] = self.request("GET", f"/motions/{motion_id}")
            if record.get("state") != "running":
                return record
            time.sleep(_POLL)

    def cancel(self, motion_id: str) -> dict[str, Any]:
        """``DELETE /api/motions/ID``: cancel it; its axes are stopped."""
        result: dict[str, Any] = self.request("DELETE", f"/motions/{motion_id}")
        return result

    def command(self, axis: str, verb: str, body: object = None) -> Any:
        """``POST /api/axes/AXIS/VERB`` (stop, halt, enable, disable, reset, jog)."""
        return self.request("POST", f"/axes/{axis}/{verb}", body if body is not None else {})

    def read(self, line: str, address: int, register: int, count: int,
             *, input: bool = False) -> list[int]:
        """Raw register read through the service's bus."""
        reply = self.request("POST", f"/lines/{line}/read", {
            "address": address, "register": register, "count": count, "input": input})
        return [int(w) for w in reply["words"]]

    def write(self, line: str, address: int, register: int, values: list[int]) -> None:
        """Raw register write through the service's bus."""
        self.request("POST", f"/lines/{line}/write",
                     {"address": address, "register": register, "values": values})

    # -- drive parameters ------------------------------------------------------------------------

    def parameters(self, axis: str) -> dict[str, Any]:
        """``GET /api/axes/AXIS/parameters``."""
        result: dict[str, Any] = self.request("GET", f"/axes/{axis}/parameters")
        return result

    def load_parameters(self, axis: str, values: dict[str, int], *, save: bool = False,
                        dry_run: bool = False, include_comms: bool = False) -> dict[str, Any]:
        """``PUT /api/axes/AXIS/parameters``: the load's report."""
        result: dict[str, Any] = self.request("PUT", f"/axes/{axis}/parameters", {
            "values": values, "save": save, "dry_run": dry_run,
            "include_comms": include_comms})
        return result
