"""What the ``drivebus`` commands share: their common arguments and options, and finding
the ``drivebus serve`` that owns a machine (used by ``cli`` and its command modules)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from drivebus.cli.args import LocalOpt, ServerOpt, TokenOpt

if TYPE_CHECKING:
    from drivebus.service.client import ServiceClient

__all__ = ["ConfigArg", "JsonOpt", "LocalOpt", "ServerOpt", "TokenOpt", "owner"]

ConfigArg = Annotated[Path, typer.Argument(help="machine file (TOML)", metavar="CONFIG")]
JsonOpt = Annotated[bool, typer.Option("--json", "-j", help="print the result as JSON")]


def owner(
    config: Path, server: str | None, token: str | None, local: bool
) -> ServiceClient | None:
    """The ``drivebus serve`` that owns ``config``'s machine (``--server``, or found
    through the file), as a client; None to open the machine here."""
    from drivebus.cli.remote import service_owner

    return service_owner(config, server, token, local)
