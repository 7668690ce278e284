"""Who is calling: bearer tokens from a token file, each with a name and a scope.

The token file has one token per line, ``NAME SCOPE TOKEN`` separated by blanks
(``#`` starts a comment)::

    # drivebus serve --token-file tokens.txt
    mes       read     9f3c51e0a4b7d2c86e1f0a9b3d5c7e21
    operator  command  1b7e4d09c2a6f8e3b5d1c0a7f9e2b4d6

``read`` may watch (GET routes, WebSocket subscriptions) and press the e-stop;
``command`` may also move, jog, stop, take the lease and write registers. A client's
NAME is its identity for the command lease and in motion records. Tokens are kept only
as SHA-256 digests and never logged; messages about the file name line numbers only.
Without a token file every client may command; it names itself with the
``X-Drivebus-Client`` header (default ``anonymous``), and the service binds loopback only.
"""

from __future__ import annotations

import hashlib
import logging
import re
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from drivebus.errors import ConfigError

__all__ = ["AuthError", "Principal", "Scope", "TokenStore", "bearer_token", "require_command"]

log = logging.getLogger(__name__)

Scope = Literal["read", "command"]
SCOPES: tuple[Scope, ...] = ("read", "command")

MIN_TOKEN_LENGTH = 16
_NAME = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")
_TOKEN = re.compile(r"^[A-Za-z0-9_.~+/=-]+$")
_CLIENT_HEADER = re.compile(r"^[A-Za-z0-9_.@:-]{1,64}$")


class AuthError(Exception):
    """A request without a valid token (401) or beyond its token's scope (403)."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status

    @property
    def name(self) -> str:
        """The problem's name: ``Unauthorized`` or ``Forbidden``."""
        return "Unauthorized" if self.status == 401 else "Forbidden"


@dataclass(frozen=True)
class Principal:
    """An authenticated caller: its name (the lease's identity) and what it may do."""

    name: str
    scope: Scope

    @property
    def may_command(self) -> bool:
        """True for the ``command`` scope."""
        return self.scope == "command"


def _digest(token: str) -> bytes:
    return hashlib.sha256(token.encode()).digest()


class TokenStore:
    """The tokens the service accepts; empty (``TokenStore()``) means no authentication."""

    def __init__(self, tokens: Mapping[str, Principal] | None = None) -> None:
        self._by_digest = {_digest(t): p for t, p in (tokens or {}).items()}

    @property
    def enabled(self) -> bool:
        """True when callers must present a token."""
        return bool(self._by_digest)

    def __len__(self) -> int:
        return len(self._by_digest)

    @classmethod
    def load(cls, path: str | Path) -> TokenStore:
        """Read a token file (format in the module's doc); ``ConfigError`` names the file
        and the line, never the token."""
        p = Path(path)
        try:
            text = p.read_text()
            mode = p.stat().st_mode
        except OSError as exc:
            raise ConfigError(f"{p}: cannot read the token file: {exc.strerror}") from None
        tokens: dict[str, Principal] = {}
        names: set[str] = set()
        for n, raw in enumerate(text.splitlines(), 1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.split()
            if len(parts) != 3:
                raise ConfigError(f"{p}:{n}: expected 'NAME SCOPE TOKEN' "
                                  f"({len(parts)} fields)")
            name, scope, token = parts
            if not _NAME.fullmatch(name):
                raise ConfigError(f"{p}:{n}: name {name!r}: use 1-64 letters, digits, _.@-")
            if scope not in SCOPES:
                raise ConfigError(f"{p}:{n}: scope {scope!r}: expected read or command")
            if len(token) < MIN_TOKEN_LENGTH or not _TOKEN.fullmatch(token):
                raise ConfigError(f"{p}:{n}: the token must be at least {MIN_TOKEN_LENGTH} "
                                  f"characters of letters, digits and _.~+/=- "
                                  f"(e.g. `openssl rand -hex 16`)")
            if name in names:
                raise ConfigError(f"{p}:{n}: name {name!r} appears twice")
            if token in tokens:
                raise ConfigError(f"{p}:{n}: this token is already given to "
                                  f"{tokens[token].name}")
            names.add(name)
            tokens[token] = Principal(name, scope)  # type: ignore[arg-type]
        if not tokens:
            raise ConfigError(f"{p}: the token file has no tokens")
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            log.warning("%s can be read by other users: chmod 600 it", p)
        return cls(tokens)

    def authenticate(self, token: str | None, client: str | None = None) -> Principal:
        """The caller presenting ``token`` (``AuthError`` 401 if it is missing or
        unknown); without tokens, the client named ``client`` may command."""
        if not self.enabled:
            name = client if client and _CLIENT_HEADER.fullmatch(client) else "anonymous"
            return Principal(name, "command")
        if not token:
            raise AuthError(401, "this service needs a bearer token: "
                                 "send 'Authorization: Bearer TOKEN'")
        return self.check(token)

    def check(self, token: str) -> Principal:
        """The principal of ``token``; ``AuthError`` 401 if it is unknown."""
        principal = self._by_digest.get(_digest(token))
        if principal is None:
            raise AuthError(401, "unknown token")
        return principal


def require_command(principal: Principal) -> Principal:
    """``principal`` if it may command; else ``AuthError`` 403."""
    if not principal.may_command:
        raise AuthError(403, f"client {principal.name} has a read-only token: "
                             f"commands need a token with the command scope")
    return principal


def bearer_token(authorization: str | None) -> str | None:
    """The token of an ``Authorization: Bearer TOKEN`` header value (None if absent);
    ``AuthError`` 401 for another scheme."""
    if not authorization:
        return None
    kind, _, token = authorization.partition(" ")
    if kind.lower() != "bearer" or not token.strip():
        raise AuthError(401, "expected 'Authorization: Bearer TOKEN'")
    return token.strip()
