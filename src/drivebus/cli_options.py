"""What the ``drivebus`` commands share: their common arguments and options, and finding
the ``drivebus serve`` that owns a machine (used by ``cli`` and its command modules)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from drivebus.service.client import ServiceClient

__all__ = ["ConfigArg", "JsonOpt", "LocalOpt", "ServerOpt", "TokenOpt", "owner"]

ConfigArg = Annotated[Path, typer.Argument(help="machine file (TOML)", metavar="CONFIG")]
JsonOpt = Annotated[bool, typer.Option("--json", "-j", help="print the result as JSON")]
ServerOpt = Annotated[str | None, typer.Option(
    "--server", metavar="URL", envvar="DRIVEBUS_SERVER",
    help="talk to this drivebus serve (default: the one serving CONFIG, if it runs)")]
TokenOpt = Annotated[str | None, typer.Option(
    "--token", metavar="TOKEN", envvar="DRIVEBUS_TOKEN",
    help="bearer token for --server (from its token file)")]
LocalOpt = Annotated[bool, typer.Option(
    "--local", help="open the machine here even if a drivebus serve owns it")]


def owner(
    config: Path, server: str | None, token: str | None, local: bool
) -> ServiceClient | None:
    """The ``drivebus serve`` that owns ``config``'s machine (``--server``, or found
    through the file), as a client; None to open the machine here."""
    from drivebus.service.client import ServiceClient, find_service

    if local:
        return None
    url = server or find_service(config)
    if url is None:
        return None
    if server is None:
        typer.echo(f"note: {config} is served by a running drivebus serve at {url}: "
                   f"talking to it (--local opens the machine here)", err=True)
    return ServiceClient(url, token=token)
