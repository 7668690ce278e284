"""Line providers: plug-ins that serve a machine file's ``SCHEME://NAME`` lines.

A line whose port or host is ``sim://NAME`` is not a device the core can open: a provider
(the built-in simulator is one) starts what serves it and says where the machine's one
line factory should connect instead. The core never imports a provider; it finds one by
its scheme, among those registered with ``register_line_provider`` and the package entry
points in the group ``drivebus.line_providers`` (drivebus's own ``pyproject.toml`` declares
``sim = "drivebus.sim.provider:SimLineProvider"``).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from drivebus.errors import ConfigError

if TYPE_CHECKING:
    from drivebus.config import LineConfig, MachineConfig

__all__ = [
    "ENTRY_POINT_GROUP",
    "LineProvider",
    "ProvidedLine",
    "line_provider",
    "register_line_provider",
    "scheme_of",
]

ENTRY_POINT_GROUP = "drivebus.line_providers"


@dataclass
class ProvidedLine:
    """What a provider started for one line: where to connect, and what it serves."""

    config: LineConfig
    """The line's config with ``port``/``host`` pointing at what the provider serves."""
    twins: dict[str, Any] = field(default_factory=dict)
    """Per axis name, the provider's stand-in for its drive (a simulated twin)."""
    server: Any = None
    """What serves the line (a simulator's wire or server: its log, faults, ...)."""


class LineProvider(Protocol):
    """A plug-in for ``SCHEME://NAME`` lines."""

    scheme: str

    def problems(self, config: MachineConfig) -> list[str]:
        """What in ``config`` this provider could not serve, as ``key.path: problem``
        (checked when the file is loaded, like the rest of it)."""
        ...

    async def open(
        self, config: MachineConfig, line: str, stack: contextlib.AsyncExitStack
    ) -> ProvidedLine:
        """Start serving line ``line`` of ``config`` until ``stack`` closes."""
        ...


_registered: dict[str, LineProvider] = {}


def register_line_provider(provider: LineProvider) -> None:
    """Make ``provider`` serve its scheme in this process (tests, embedding applications)."""
    _registered[provider.scheme] = provider


def scheme_of(address: str | None) -> str | None:
    """The scheme of a provider address (``sim`` for ``sim://NAME``), else None."""
    if not address or "://" not in address:
        return None
    scheme = address.split("://", 1)[0]
    return scheme if scheme.isidentifier() else None


def line_provider(scheme: str) -> LineProvider:
    """The provider for ``scheme``; ``ConfigError`` if none is installed."""
    found = _registered.get(scheme)
    if found is not None:
        return found
    from importlib.metadata import entry_points  # the installed providers, when asked for

    for ep in entry_points(group=ENTRY_POINT_GROUP, name=scheme):
        provider: LineProvider = ep.load()()
        _registered[scheme] = provider
        return provider
    known = sorted({*_registered, *(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))})
    raise ConfigError(
        f"no line provider for {scheme}:// is installed (known: {', '.join(known) or 'none'})"
    )
